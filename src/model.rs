//! Closures of docs/model.md on a finite-volume grid: shear rate, pressure,
//! mu(I), segregation speed and diffusivity, and the initial condition.

use crate::params::Params;

/// Uniform cell-centred grid on [0, H], z pointing up from the bottom wall.
#[derive(Clone, Debug)]
pub struct Grid {
    pub n: usize,
    pub dz: f64,
    pub h: f64,
}

impl Grid {
    pub fn new(n: usize, h: f64) -> Self {
        Grid {
            n,
            dz: h / n as f64,
            h,
        }
    }

    /// Cell centres, m.
    pub fn centres(&self) -> Vec<f64> {
        (0..self.n).map(|i| (i as f64 + 0.5) * self.dz).collect()
    }

    /// Height of interior face f (between cells f and f + 1), m.
    #[inline]
    pub fn face(&self, f: usize) -> f64 {
        (f + 1) as f64 * self.dz
    }
}

/// mu(I) of Jop et al.: mu_min + (mu_2 - mu_min) / (I0 / I + 1).
#[inline]
pub fn mu_of_i(p: &Params, i: f64) -> f64 {
    p.mu_min + (p.mu_2 - p.mu_min) * i / (p.i0 + i)
}

/// d mu / d I.
#[inline]
pub fn dmu_di(p: &Params, i: f64) -> f64 {
    let s = p.i0 + i;
    (p.mu_2 - p.mu_min) * p.i0 / (s * s)
}

/// Shear-rate magnitude at height z for decay length delta, 1/s.
#[inline]
pub fn shear_rate(p: &Params, delta: f64, z: f64) -> f64 {
    (p.v0() - p.v1) / delta * (-z / delta).exp()
}

/// Velocity profile v(z), m/s.
pub fn velocity(p: &Params, delta: f64, z: f64) -> f64 {
    p.v1 + (p.v0() - p.v1) * (-z / delta).exp()
}

/// Stokes prefactor of the segregation speed, D_p^2 g (rho_h - rho_l) / 18,
/// in m^3/s^2 per (Pa s): w = stokes (1 - c) gdot / (k mu P).
#[inline]
pub fn stokes_prefactor(p: &Params) -> f64 {
    p.d_p * p.d_p * p.g * (p.rho_h - p.rho_l) / 18.0
}

/// Segregation-speed coefficient a such that w = a (1 - c), m/s, together
/// with da/dP (used by the pressure-coupled Jacobian).
#[inline]
pub fn seg_coefficient(
    p: &Params,
    stokes: f64,
    gdot: f64,
    rho_m: f64,
    pressure: f64,
) -> (f64, f64) {
    let inertial = gdot * p.d_p * (rho_m * p.phi_s / pressure).sqrt();
    let mu = mu_of_i(p, inertial);
    let a = stokes * gdot / (p.k * mu * pressure);
    // dI/dP = -I / (2P); da/dP = -a/P - a/mu dmu/dI dI/dP
    let da_dp = -a / pressure + a / mu * dmu_di(p, inertial) * inertial / (2.0 * pressure);
    (a, da_dp)
}

/// The C2 quintic smoothed step: 0 for x <= -1, 1 for x >= 1.
#[inline]
pub fn quintic_step(x: f64) -> f64 {
    if x <= -1.0 {
        0.0
    } else if x >= 1.0 {
        1.0
    } else {
        let u = (x + 1.0) / 2.0;
        u * u * u * (u * (6.0 * u - 15.0) + 10.0)
    }
}

/// Antiderivative of the quintic step in x (for exact cell averages).
fn quintic_step_integral(x: f64) -> f64 {
    // integral_{-1}^{x} S(s) ds ; for x >= 1 it is x (since integral over [-1, 1] = 1).
    if x <= -1.0 {
        0.0
    } else if x >= 1.0 {
        x
    } else {
        let u = (x + 1.0) / 2.0;
        // ds = 2 du; integral of 6u^5-15u^4+10u^3 = u^6 - 3u^5 + 2.5u^4
        2.0 * (u.powi(6) - 3.0 * u.powi(5) + 2.5 * u.powi(4))
    }
}

/// Initial condition: heavy above light, interface at (1 - c0) H smoothed
/// over eps = D_p / 2. Returned as exact cell averages, so that the discrete
/// depth-mean is c0 to round-off.
pub fn initial_condition(p: &Params, grid: &Grid) -> Vec<f64> {
    let eps = p.d_p / 2.0;
    let zbar = (1.0 - p.c0) * p.h;
    (0..grid.n)
        .map(|i| {
            let x0 = (i as f64 * grid.dz - zbar) / eps;
            let x1 = ((i + 1) as f64 * grid.dz - zbar) / eps;
            if x0 >= 1.0 {
                1.0
            } else if x1 <= -1.0 {
                0.0
            } else {
                let v = eps * (quintic_step_integral(x1) - quintic_step_integral(x0)) / grid.dz;
                v.clamp(0.0, 1.0)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_condition_has_mean_c0() {
        for &c0 in &[0.05, 0.1, 0.5, 0.77, 0.95] {
            for &n in &[15usize, 37, 180, 1000] {
                let p = Params {
                    c0,
                    ..Params::default()
                };
                let g = Grid::new(n, p.h);
                let c = initial_condition(&p, &g);
                let mean = c.iter().sum::<f64>() / n as f64;
                assert!((mean - c0).abs() < 1e-12, "c0={c0} n={n} mean={mean}");
                assert!(c.iter().all(|&v| (0.0..=1.0).contains(&v)));
            }
        }
    }

    #[test]
    fn quintic_integral_is_consistent() {
        // derivative of the antiderivative is the step
        for &x in &[-0.9, -0.3, 0.0, 0.4, 0.95] {
            let h = 1e-6;
            let d = (quintic_step_integral(x + h) - quintic_step_integral(x - h)) / (2.0 * h);
            assert!((d - quintic_step(x)).abs() < 1e-8);
        }
    }

    #[test]
    fn seg_coefficient_derivative_matches_finite_difference() {
        let p = Params::default();
        let s = stokes_prefactor(&p);
        let (a, da) = seg_coefficient(&p, s, 3.0, 1700.0, 800.0);
        let (a2, _) = seg_coefficient(&p, s, 3.0, 1700.0, 800.0 + 1e-3);
        assert!(a > 0.0);
        assert!(((a2 - a) / 1e-3 - da).abs() < 1e-6 * da.abs().max(1e-12) + 1e-12);
    }
}
