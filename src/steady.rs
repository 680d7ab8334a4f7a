//! The long-time profile, solved directly in z without time stepping.
//!
//! With F = 0 everywhere, D dc/dz = -w c, i.e. in the logit u = ln(c/(1-c))
//!
//!   du/dz = -Lambda(z) = -g (rho_h - rho_l) / (18 b k mu(I) P)
//!   dP/dz = -g phi_s rho_m(c)
//!
//! (the shear rate cancels except inside I). Both are integrated down from
//! the lid, P(H) = P_load, for a trial logit at the top; the top value is
//! found by bracketed root finding so that the depth-mean of c is c0. The
//! logit keeps the profile strictly inside (0, 1) at any density ratio.

use std::sync::atomic::AtomicBool;

use crate::error::SolveError;
use crate::limits;
use crate::model::{self, Grid};
use crate::params::Params;

#[inline]
fn logistic(u: f64) -> f64 {
    if u >= 0.0 {
        1.0 / (1.0 + (-u).exp())
    } else {
        let e = u.exp();
        e / (1.0 + e)
    }
}

struct Shooter<'a> {
    p: &'a Params,
    delta: f64,
    lambda0: f64,
    grid: Grid,
    sub: usize,
}

impl Shooter<'_> {
    /// Right-hand side of (u, P) in z.
    #[inline]
    fn deriv(&self, z: f64, u: f64, pres: f64) -> (f64, f64) {
        let c = logistic(u);
        let rho = self.p.rho_m(c);
        let gdot = model::shear_rate(self.p, self.delta, z);
        let inertial = gdot * self.p.d_p * (rho * self.p.phi_s / pres).sqrt();
        let mu = model::mu_of_i(self.p, inertial);
        (-self.lambda0 / (mu * pres), -self.p.g * self.p.phi_s * rho)
    }

    /// Cell averages of c (Simpson per cell) for the trial top logit;
    /// `Interrupted` if `stop` is set (polled every 256 cells).
    fn profile(&self, u_top: f64, out: &mut [f64], stop: &AtomicBool) -> Result<(), SolveError> {
        let n = self.grid.n;
        let m = self.sub; // even number of RK4 sub-steps per cell
        let hz = -self.grid.dz / m as f64;
        let (mut u, mut pres) = (u_top, self.p.p_load());
        let mut z = self.p.h;
        for cell in (0..n).rev() {
            if cell % 256 == 0 {
                limits::check_stop(stop)?;
            }
            let mut acc = logistic(u);
            for s in 0..m {
                let (k1u, k1p) = self.deriv(z, u, pres);
                let (k2u, k2p) =
                    self.deriv(z + 0.5 * hz, u + 0.5 * hz * k1u, pres + 0.5 * hz * k1p);
                let (k3u, k3p) =
                    self.deriv(z + 0.5 * hz, u + 0.5 * hz * k2u, pres + 0.5 * hz * k2p);
                let (k4u, k4p) = self.deriv(z + hz, u + hz * k3u, pres + hz * k3p);
                u += hz / 6.0 * (k1u + 2.0 * k2u + 2.0 * k3u + k4u);
                pres += hz / 6.0 * (k1p + 2.0 * k2p + 2.0 * k3p + k4p);
                z += hz;
                let wgt = if s + 1 == m {
                    1.0
                } else if s % 2 == 0 {
                    4.0
                } else {
                    2.0
                };
                acc += wgt * logistic(u);
            }
            out[cell] = acc / (3.0 * m as f64);
        }
        Ok(())
    }

    fn excess_mass(
        &self,
        u_top: f64,
        buf: &mut [f64],
        stop: &AtomicBool,
    ) -> Result<f64, SolveError> {
        self.profile(u_top, buf, stop)?;
        Ok(buf.iter().sum::<f64>() / buf.len() as f64 - self.p.c0)
    }
}

/// Steady profile as cell averages on `n_cells` cells (centres from
/// `Grid::centres`). `sub_steps` RK4 steps per cell (rounded up to even);
/// the result is converged to ~1e-10 for sub_steps >= 16 at 180 cells.
/// At most `limits::MAX_CELLS` cells and `limits::MAX_SUB_STEPS` sub-steps.
pub fn steady_state(p: &Params, n_cells: usize, sub_steps: usize) -> Result<Vec<f64>, SolveError> {
    steady_state_stoppable(p, n_cells, sub_steps, limits::never())
}

/// `steady_state` that returns `SolveError::Interrupted` soon after `stop` is set.
pub fn steady_state_stoppable(
    p: &Params,
    n_cells: usize,
    sub_steps: usize,
    stop: &AtomicBool,
) -> Result<Vec<f64>, SolveError> {
    if p.laws.active() {
        return Err(SolveError::InvalidInput(
            "steady_state: the law corrections (law_*) are not supported; simulate to long times instead".into(),
        ));
    }
    p.validate()?;
    if n_cells < 15 {
        return Err(SolveError::InvalidInput(format!(
            "n_cells = {n_cells} is out of range: must be >= 15"
        )));
    }
    limits::check_cells(n_cells)?;
    if sub_steps > limits::MAX_SUB_STEPS {
        return Err(SolveError::InvalidInput(format!(
            "sub_steps = {sub_steps} is out of range: must be <= {}",
            limits::MAX_SUB_STEPS
        )));
    }
    let sub = sub_steps.max(2).div_ceil(2) * 2;
    let shooter = Shooter {
        p,
        delta: p.delta_over_h * p.h * (1.0 + p.delta_drift),
        lambda0: p.g * (p.rho_h - p.rho_l) / (18.0 * p.b * p.k),
        grid: Grid::new(n_cells, p.h),
        sub,
    };
    let mut buf = limits::zeroed(n_cells, "the steady profile")?;
    let (mut lo, mut hi) = (-40.0, 40.0);
    let mut f_lo = shooter.excess_mass(lo, &mut buf, stop)?;
    let mut f_hi = shooter.excess_mass(hi, &mut buf, stop)?;
    let mut tries = 0;
    while f_lo > 0.0 || f_hi < 0.0 {
        tries += 1;
        if tries > 60 {
            return Err(SolveError::SteadyFailure(
                "could not bracket the top concentration".into(),
            ));
        }
        if f_lo > 0.0 {
            lo = 2.0 * lo - 10.0;
            f_lo = shooter.excess_mass(lo, &mut buf, stop)?;
        }
        if f_hi < 0.0 {
            hi = 2.0 * hi + 10.0;
            f_hi = shooter.excess_mass(hi, &mut buf, stop)?;
        }
    }
    // Illinois regula falsi with a bisection safeguard.
    let mut side = 0i32;
    for _ in 0..200 {
        let mut mid = (lo * f_hi - hi * f_lo) / (f_hi - f_lo);
        if !mid.is_finite() || mid <= lo || mid >= hi {
            mid = 0.5 * (lo + hi);
        }
        let f_mid = shooter.excess_mass(mid, &mut buf, stop)?;
        if f_mid.abs() < 1e-14 || (hi - lo) < 1e-13 {
            return Ok(buf);
        }
        if f_mid < 0.0 {
            lo = mid;
            f_lo = f_mid;
            if side == -1 {
                f_hi *= 0.5;
            }
            side = -1;
        } else {
            hi = mid;
            f_hi = f_mid;
            if side == 1 {
                f_lo *= 0.5;
            }
            side = 1;
        }
    }
    Err(SolveError::SteadyFailure(
        "root finding for the top concentration did not converge".into(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_density_is_uniform() {
        let p = Params {
            rho_h: 1750.0,
            rho_l: 1750.0,
            c0: 0.37,
            ..Params::default()
        };
        let c = steady_state(&p, 30, 8).unwrap();
        assert!(c.iter().all(|v| (v - 0.37).abs() < 1e-12));
    }

    #[test]
    fn has_the_right_mass_and_is_monotone() {
        for &(rho_h, c0) in &[(2450.0, 0.5), (7800.0, 0.1), (3500.0, 0.9)] {
            let p = Params {
                rho_h,
                c0,
                ..Params::default()
            };
            let c = steady_state(&p, 180, 16).unwrap();
            let mean = c.iter().sum::<f64>() / 180.0;
            assert!((mean - c0).abs() < 1e-12);
            assert!(c.windows(2).all(|w| w[1] <= w[0]));
        }
    }

    #[test]
    fn sizes_are_bounded_and_a_stop_flag_interrupts() {
        let p = Params::default();
        let e = steady_state(&p, 100_000_000, 16).unwrap_err();
        assert!(
            e.is_input_error() && e.to_string().contains("n_cells = 100000000"),
            "{e}"
        );
        let e = steady_state(&p, 180, usize::MAX).unwrap_err();
        assert!(e.to_string().contains("sub_steps"), "{e}");
        let stop = AtomicBool::new(true);
        let e = steady_state_stoppable(&p, 180, 16, &stop).unwrap_err();
        assert_eq!(e, SolveError::Interrupted);
    }

    #[test]
    fn resolution_converges() {
        let p = Params {
            rho_h: 7800.0,
            ..Params::default()
        };
        let a = steady_state(&p, 90, 8).unwrap();
        let b = steady_state(&p, 90, 64).unwrap();
        let err = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-8, "{err}");
    }
}
